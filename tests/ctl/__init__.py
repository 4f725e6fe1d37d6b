"""gx2ctl as a user runs it, against a fake gateway on real sockets."""
