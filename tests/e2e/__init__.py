"""The installed gx2-gateway through a real pty (gx2-sim) and real ZeroMQ sockets."""
