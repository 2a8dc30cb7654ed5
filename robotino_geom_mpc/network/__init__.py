"""The radio link between the robot and the off-board controller: link emulation and packetized command plans."""
