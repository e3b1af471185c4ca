"""Bus tools: the sniffer and its CANopen service names, recorders, replay, pcap files,
and the EDS checker."""
