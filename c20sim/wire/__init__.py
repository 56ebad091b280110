"""The wire: the sheet's bytes, registers and exception codes. Pure; imports nothing else of c20sim."""
