"""What a CANopen device says it is: object 0x1018, vendor-ID, product code, revision
number and serial number. LSS addresses a device by it, a non-volatile store names the
device it belongs to by it, and the host tells a patch from a force node by its product
code (eds/skin-patch.eds: 1, eds/skin-forces.eds: 2; vendor 0)."""

from __future__ import annotations

from dataclasses import astuple, dataclass

PATCH_PRODUCT = 1
FORCE_PRODUCT = 2


@dataclass(frozen=True)
class Identity:
    """Object 0x1018 sub 1..4: vendor-ID, product code, revision number, serial number."""

    vendor: int
    product: int
    revision: int
    serial: int

    @property
    def kind(self) -> str:
        """``"patch"``, ``"forces"`` or ``"unknown"``."""
        if self.vendor != 0:
            return "unknown"
        return {PATCH_PRODUCT: "patch", FORCE_PRODUCT: "forces"}.get(self.product, "unknown")

    def as_dict(self) -> dict[str, int]:
        return dict(zip(("vendor", "product", "revision", "serial"), astuple(self), strict=True))
