"""What all three programs share: endpoints, topics, the control protocol's limits,
error kinds and exit codes, the op table, the values a command line or a request
carries, command-line helpers, YAML files and CURVE keys.

None of it imports pydantic, so gx2ctl starts quickly; the one exception,
:mod:`gateway.common.strict`, is for the two programs that validate files with it.
"""
