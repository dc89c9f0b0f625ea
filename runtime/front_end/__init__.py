"""The front end (local SLAM): tracking each scan against the keyframe's submap, the odometry gate
and recovery, node insertion and the scans' trajectory (docs/method.md §6)."""
