"""Small shared helpers: atomic file writes (:mod:`.io`), tensor layouts and shape checks
(:mod:`.tensors`), stage timing (:mod:`.timing`)."""
