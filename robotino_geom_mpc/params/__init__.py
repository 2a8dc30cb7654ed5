"""Parameters of the Robotino and its controller: the specs (one source), parameter files, presets."""
