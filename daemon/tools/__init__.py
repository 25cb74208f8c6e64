"""What stands around the service: fault and soak drivers, the fuzzer.

Each tool is a command, ``python -m scotti.daemon.tools.<name>``; none is
imported by the daemon itself.
"""
