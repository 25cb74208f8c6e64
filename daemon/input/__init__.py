"""Where the bytes come from: the receiver's serial port, a session file replayed, or the
simulated board; and ``--record``, which taps them before decoding."""
