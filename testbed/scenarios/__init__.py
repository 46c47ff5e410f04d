"""Paper examples as data: plant, signals, horizon, filter settings and the printed claims."""
