"""Surface stages: hands, motion evidence, part masks, TSDF fusion and gravity."""
