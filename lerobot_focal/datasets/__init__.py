"""Datasets, by job: :mod:`.making` writes them, :mod:`.repair` recovers what a killed writer left, and
:mod:`.fast_loading` reads them faster during training (opt-in)."""
