"""Where the camera is and what the screen shows: the camera convention, the framing of a
request, and the screen regions a frame's surfaces can reach.

Plain geometry: imports `core` only."""
