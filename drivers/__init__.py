"""Device codecs, framers and transports: bytes in, immutable typed messages out (and back)."""
