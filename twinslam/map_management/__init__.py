"""Map-management policies (LFF, PU, ADAPT) and the action/observation types they exchange."""
