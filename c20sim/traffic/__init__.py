"""Traffic: captures and frame logs read back (capture), sniffed off a line (record), played again (replay)."""
