"""A patch's data-plane side: its channel follows its state, its EMCYs mask its taxels.

While a patch is operational the data plane decodes it with a channel built from its
set-up (decoder, baseline for tare and drift); in every other state it has a placeholder
channel, offline, so its force node still publishes one all-invalid sample per SYNC and
no consumer keeps its last forces. :meth:`PatchChannels.apply` is the
:class:`~canbus.master.patchstate.PatchStates`' ``apply``: it runs, in order, with every
change of state.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
from canopen.emcy import EmcyError
from numpy.typing import NDArray

from canbus.master.baseline import Baseline
from canbus.master.channel import PatchChannel
from canbus.master.contactconfig import take_pitch
from canbus.master.decoders import DecoderCache
from canbus.master.emcy import DEVICE_HARDWARE, EmcyLog, taxel_of
from canbus.master.hostconfig import HostConfig
from canbus.master.patch_setup import PatchSetup
from canbus.master.patchstate import Facts, Transition
from canbus.master.records import PatchRecord
from skin.constants import TAXELS_PER_PATCH


class PatchChannels:
    """The channels of ``patches`` in their buses' data planes."""

    def __init__(self, config: HostConfig, patches: dict[int, PatchRecord],
                 decoders: DecoderCache, running: threading.Event) -> None:
        self.config = config
        self.patches = patches
        self.decoders = decoders
        self.running = running  # set while the host runs: a late change brings none online
        self.emcy_log = EmcyLog()

    def placeholder(self, patch: PatchRecord, setup: PatchSetup) -> None:
        """An offline channel for a patch not decoded yet: its all-invalid sample per SYNC."""
        dataplane = patch.link.dataplane
        assert dataplane is not None
        decoder, _ = self.decoders.get(patch.config, setup)
        dataplane.add_channel(PatchChannel(
            node_id=patch.node_id, codec=setup.codec, pillars=setup.pillars,
            lsb_ohm=setup.info.lsb_ohm, decoder=decoder, force_node=patch.force_node,
            masked=patch.masked, answer_order=patch.config.answer_order), online=False)

    def apply(self, transition: Transition, facts: Facts) -> None:
        """A patch changed state (the states' lock is held): decode it while operational."""
        patch = self.patches[transition.node_id]
        if transition.new == "operational" and facts.setup is not None and \
                self.running.is_set():
            self._online(patch, facts.setup)
        elif transition.old == "operational":
            self._offline(patch)

    def _offline(self, patch: PatchRecord) -> None:
        dataplane = patch.link.dataplane
        if patch.channel is not None and dataplane is not None:
            dataplane.set_online(patch.node_id, False)
        patch.channel = None

    def _online(self, patch: PatchRecord, setup: PatchSetup) -> None:
        dataplane = patch.link.dataplane
        if dataplane is None:
            return
        decoder, r0_ref = self.decoders.get(patch.config, setup)
        p = setup.pillars
        drift = self.config.drift
        baseline = Baseline(
            r0_ref, setup.info.r0_ohm[:, :p], loaded_N=self.config.tare_threshold_N,
            time_constant_s=None if drift is None else drift.time_constant_s,
            contact_N=0.1 if drift is None else drift.contact_N)
        channel = PatchChannel(
            node_id=patch.node_id, codec=setup.codec, pillars=p, lsb_ohm=setup.info.lsb_ohm,
            decoder=decoder, force_node=patch.force_node, masked=patch.masked,
            baseline=baseline, answer_order=patch.config.answer_order)
        take_pitch(patch.force_node.contact, setup.info.constants)
        dataplane.add_channel(channel)
        patch.channel = channel

    def set_mask(self, patch: PatchRecord, taxels: NDArray[np.bool_], masked: bool) -> None:
        """Mask (or unmask) ``taxels`` for the samples completed from now on.

        The data plane reads a patch's mask when it publishes, which may be after the
        next cycle's frames arrived; so the samples already complete are published
        first, with the mask they were completed under: an EMCY (or boot-up) applies
        from its place on the bus, live and in a replay alike. Never under the states'
        lock: publishing runs the force callbacks, which may call the API.
        """
        if bool(np.all(patch.masked[taxels] == masked)):
            return
        dataplane = patch.link.dataplane
        if dataplane is not None:
            dataplane.publish_pending()
        patch.masked[taxels] = masked

    def booted(self, patch: PatchRecord) -> None:
        """A boot-up clears the patch's EMCY mask."""
        self.set_mask(patch, np.ones(TAXELS_PER_PATCH, dtype=bool), False)

    def emcy_handler(self, patch: PatchRecord) -> Callable[[EmcyError], None]:
        """The callback of the patch's EMCY consumer: logged, a taxel masked or unmasked."""
        def on_emcy(entry: EmcyError) -> None:
            self.emcy_log.note(patch.node_id, entry)
            taxel = taxel_of(entry)
            if taxel is None:
                return
            which = np.zeros(TAXELS_PER_PATCH, dtype=bool)
            which[taxel] = True
            self.set_mask(patch, which, entry.code == DEVICE_HARDWARE)
        return on_emcy
