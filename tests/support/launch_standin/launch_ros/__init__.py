"""A stand-in for ``launch_ros`` (see the ``launch`` stand-in's docstring)."""
