"""Readers and writers of every on-disk layout (docs/formats.md): capture, camera poses, twin, affordances,
fragments, ground truth. Only numpy, the standard library and image I/O."""
