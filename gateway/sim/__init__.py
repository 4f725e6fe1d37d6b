"""gx2-sim: a virtual 3DM-GX2 wireless base station and its nodes behind a pty."""
