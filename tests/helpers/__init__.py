"""What the tests (and bench/) share: free ports, waiting with a deadline, packet
builders, decoding helpers, the console scripts, and a running gateway's harness."""
