"""The device's front end: ORB features, the local map of points it tracks against, motion-only
pose refinement, tracking with relocalisation, the features it follows for the edge and where
its map comes from. It knows nothing of the edge's back end (a contract says so)."""
