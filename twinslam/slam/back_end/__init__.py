"""The edge's back end: the keyframe map with its covisibility and checkpoint, uploaded keyframes
into the map, GTSAM local bundle adjustment, the archive of evicted keyframes and place
recognition over it. It knows nothing of the device's front end (a contract says so)."""
