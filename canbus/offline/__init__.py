"""The host without a bus: forces decoded from a recording by the listen-only host on the
recording's own clock (``decode``), the resistances a recording carries, one sample per
patch per SYNC (``recorded``), and a calibration dataset from a recording and reference
forces (``dataset``)."""
