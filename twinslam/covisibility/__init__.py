"""Covisibility datasets: for every frame of a sequence, the map points the front end observes
in it (``dataset.py``), the weights between frames they give, a map's point counts kept up to
date (``map_points.py``) and a geometric room model that makes such data without a sequence
(``geometric.py``). The data the world model, the simulator and the calibration share."""
