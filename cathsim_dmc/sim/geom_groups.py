"""Geom groups (what renders draw) and collision bits shared by all entities.

Renders for observations draw groups 0-2 only; the thousands of wall collision pieces
(group 3) are never drawn, since software GL pays per drawn mesh.
"""

VISUAL = 1  # the vessel's merged visual mesh, robot parts
WIRE = 2  # guidewire segments (the segmentation mask renders this group alone)
COLLISION = 3  # wall collision pieces
MARKER = 4  # sites, targets: drawn only in videos and viewers

# The wire collides with the wall and the guide channel, never with itself.
WIRE_CONTYPE, WIRE_CONAFFINITY = 2, 1
WALL_CONTYPE, WALL_CONAFFINITY = 1, 2
