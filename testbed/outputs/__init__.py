"""What a run leaves for people: figures, Rerun recordings, the live viewer, videos, and the
units they are shown in."""
