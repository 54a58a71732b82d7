"""Planner measurements: ``cellctl bench plan`` and ``cellctl bench whole-bin`` (:mod:`.plans`), their
row summaries (:mod:`.rows`) and the shape-family meshes they plan (:mod:`.family`)."""
