"""The gateway programs: gx2-sim now; the gx2-gateway daemon and gx2ctl next."""
