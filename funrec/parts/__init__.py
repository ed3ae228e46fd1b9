"""Part stages: scene change, fragments, point tracks, articulation, part motion and joint states."""
