"""edge_mapper: the edge's keyframe map, keyframe integration, GTSAM back end, slot planning,
node."""
