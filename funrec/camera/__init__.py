"""Camera stages: features, frame-to-frame tracking, pose graph, submaps and their global alignment."""
