"""SLAM pieces device and edge share: projection matching and the keyframe/map payloads."""
