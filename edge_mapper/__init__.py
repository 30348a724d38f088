"""edge_mapper: the edge map — covisibility graph, uncertainty, policies, GTSAM back end."""
