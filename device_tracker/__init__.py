"""device_tracker: ORB front end, local tracking, frame summaries and the uplink shaper."""
