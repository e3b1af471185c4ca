# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""SDO server: canopen's ``SdoServer`` with the CiA 301 checks it leaves out.

canopen's server (2.4) trusts its input: a frame shorter than 8 bytes raises
``struct.error`` inside the network's receive thread, a segment without an initiated
transfer touches ``None``, an abort before any request packs ``None`` as the index, an
expedited download without a size indicator always writes 4 bytes, and the size a
segmented download announces is never compared with what arrives. This subclass keeps
canopen's transfer code and adds, following CiA 301:

* frames whose length is not 8 are not SDO requests and are ignored (logged);
* a segment request with no transfer in progress aborts with 0x05040001;
* an expedited download without size indication writes the object's own size;
* an announced size that does not match what arrives aborts with 0x06070010;
* a segmented download is checked at its initiate: a missing object or sub-index, a
  read-only object (0x06010002), and an announced size larger (0x06070012) or smaller
  (0x06070013) than a number object holds abort before any segment;
* a block upload or download initiate aborts with 0x05040001 (block transfer is not
  supported; canopen's server would answer a block upload with an expedited upload);
* every abort names the index and subindex of the request being answered.
"""

from __future__ import annotations

import logging
import struct
from typing import Any

from canopen.objectdictionary import NUMBER_TYPES
from canopen.sdo.constants import (
    EXPEDITED,
    NO_MORE_DATA,
    REQUEST_ABORTED,
    REQUEST_BLOCK_DOWNLOAD,
    REQUEST_BLOCK_UPLOAD,
    REQUEST_DOWNLOAD,
    REQUEST_SEGMENT_DOWNLOAD,
    REQUEST_SEGMENT_UPLOAD,
    REQUEST_UPLOAD,
    SIZE_SPECIFIED,
)
from canopen.sdo.exceptions import SdoAbortedError
from canopen.sdo.server import SdoServer

logger = logging.getLogger(__name__)

ABORT_TOGGLE = 0x0503_0000
ABORT_COMMAND = 0x0504_0001
ABORT_LENGTH = 0x0607_0010
ABORT_TOO_LONG, ABORT_TOO_SHORT = 0x0607_0012, 0x0607_0013
ABORT_READ_ONLY = 0x0601_0002
ABORT_GENERAL = 0x0800_0000
_INITIATE = (REQUEST_UPLOAD, REQUEST_DOWNLOAD, REQUEST_BLOCK_UPLOAD, REQUEST_BLOCK_DOWNLOAD)


class StrictSdoServer(SdoServer):
    """An expedited and segmented SDO server over a ``LocalNode``'s object dictionary."""

    def __init__(self, rx_cobid: int, tx_cobid: int, node: Any) -> None:
        super().__init__(rx_cobid, tx_cobid, node)
        self._index = 0
        self._subindex = 0
        self._transfer: str | None = None  # "upload" | "download" while segmented
        self._announced: int | None = None

    def on_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) != 8:
            logger.info("ignored SDO frame of %d bytes on 0x%03X", len(data), can_id)
            return
        command = data[0]
        ccs = command & 0xE0
        if ccs in _INITIATE or ccs == REQUEST_ABORTED:
            _, self._index, self._subindex = struct.unpack_from("<BHB", data)
        try:
            self._dispatch(ccs, command, bytes(data))
        except SdoAbortedError as exc:
            self._end()
            self.abort(exc.code)
        except Exception:
            logger.exception("SDO request failed for 0x%04X:%02X", self._index, self._subindex)
            self._end()
            self.abort(ABORT_GENERAL)

    def _dispatch(self, ccs: int, command: int, data: bytes) -> None:
        if ccs in (REQUEST_BLOCK_UPLOAD, REQUEST_BLOCK_DOWNLOAD):
            self._end()
            raise SdoAbortedError(ABORT_COMMAND)
        if ccs == REQUEST_UPLOAD:
            self._end()
            self.init_upload(data)
            if self._buffer is not None:
                self._transfer = "upload"
        elif ccs == REQUEST_DOWNLOAD:
            self._end()
            self.init_download(data)
        elif ccs == REQUEST_SEGMENT_UPLOAD:
            if self._transfer != "upload":
                raise SdoAbortedError(ABORT_COMMAND)
            self.segmented_upload(command)
            if not self._buffer:
                self._end()
        elif ccs == REQUEST_SEGMENT_DOWNLOAD:
            if self._transfer != "download":
                raise SdoAbortedError(ABORT_COMMAND)
            if command & NO_MORE_DATA:
                received = len(self._buffer or b"") + 7 - ((command >> 1) & 0x7)
                if self._announced is not None and received != self._announced:
                    raise SdoAbortedError(ABORT_LENGTH)
            self.segmented_download(command, data)
            if command & NO_MORE_DATA:
                self._end()
        elif ccs == REQUEST_ABORTED:
            self._end()
            self.request_aborted(data)
        else:
            raise SdoAbortedError(ABORT_COMMAND)

    def init_download(self, request: bytes) -> None:
        command = request[0]
        if command & EXPEDITED and not command & SIZE_SPECIFIED:
            size = len(self._node._find_object(self._index, self._subindex)) // 8
            if size <= 4:
                command |= SIZE_SPECIFIED | ((4 - size) << 2)
                request = bytes([command]) + request[1:]
        if not command & EXPEDITED:
            self._check_segmented(command, request)
        super().init_download(request)
        if not command & EXPEDITED:
            self._transfer = "download"
            self._announced = (struct.unpack_from("<L", request, 4)[0]
                               if command & SIZE_SPECIFIED else None)

    def _check_segmented(self, command: int, request: bytes) -> None:
        obj = self._node._find_object(self._index, self._subindex)
        if not obj.writable:
            raise SdoAbortedError(ABORT_READ_ONLY)
        if command & SIZE_SPECIFIED and obj.data_type in NUMBER_TYPES:
            announced = struct.unpack_from("<L", request, 4)[0]
            if 8 * announced > len(obj):
                raise SdoAbortedError(ABORT_TOO_LONG)
            if 8 * announced < len(obj):
                raise SdoAbortedError(ABORT_TOO_SHORT)

    def _end(self) -> None:
        self._transfer = None
        self._announced = None
        self._buffer = None
