"""gx2-sim: node and base station on a test clock, the pty, the command line."""
