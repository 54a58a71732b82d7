"""Classifier measurements: ``cellctl bench classify`` (:mod:`.variants`), ``cellctl bench reference``
(:mod:`.reference`, on the generated twin pairs of :mod:`.pairs`) and ``cellctl bench inspect``
(:mod:`.inspect`; ``--commissioned`` in :mod:`.inspect_commissioned`)."""
