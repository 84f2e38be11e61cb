"""Online estimation: incremental smoothing (:mod:`.incremental`)."""
