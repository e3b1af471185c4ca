"""What every command shares: the bus flags (``busargs``), a config's path (``configpath``),
CPU pinning (``cpu``), the host's buses from flags or a config (``hostbus``), logging
(``logs``), stop signals (``signals``), tables (``tables``) and one BLAS thread for the
commands that train (``blas``)."""
