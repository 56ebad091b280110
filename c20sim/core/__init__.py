"""Drives on one line, still pure: the Modbus slave, the bus, link faults, clocks, generators, the simulator.

Imports wire/ and drive/ only; no I/O (transport/ is the only layer that touches a port or a socket).
"""
