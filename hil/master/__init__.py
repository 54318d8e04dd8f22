"""The master side: the client that drives the emulator or a real vehicle (:mod:`.client`) and the
decoder of recorded bus logs into measurements (:mod:`.decode`)."""
