"""Device codecs, framers and transports: bytes in, immutable typed messages out (and back)."""

if __name__ != "auvgw.drivers":
    raise ImportError(f"import auvgw.drivers, not {__name__}: the folder is mapped (setup.py)")
