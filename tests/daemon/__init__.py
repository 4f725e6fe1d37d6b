"""The daemon's parts on their own: scheduler, nodes, supervisor, operations, control, link."""
