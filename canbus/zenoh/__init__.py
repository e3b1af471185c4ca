"""The skin on Zenoh: every host's force samples, events and statistics, for any reader.

``canbus.zenoh.schema`` (keys and the sample's bytes), ``config`` (the ``[zenoh]``
table), ``publisher`` (a host's side, one way), ``reader`` (``subscribe``). Zenoh itself
(``eclipse-zenoh``, the ``canskin[zenoh]`` extra) is imported only by the publisher and
the reader. Reference: ``docs/zenoh.md``.
"""
