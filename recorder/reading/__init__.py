"""A recording read back: the reader, the trust gate, the decoder, recovery of a cut file."""
