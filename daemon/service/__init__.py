"""The daemon's life: the command line, one device per insole pair, the worker
processes, systemd notify, and the numbers that health reports."""
