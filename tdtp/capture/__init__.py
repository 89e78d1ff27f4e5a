"""Packet captures that Wireshark opens.

* :mod:`tdtp.capture.pcap`: UDP datagrams written as a classic pcap file with real IP and UDP headers,
  for ``tools/wireshark/tdtp.lua`` to decode.
"""
