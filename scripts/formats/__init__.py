"""The file formats, one module each, reader and writer: CARMEN logs (the neutral log records too),
ROS bags and MCAP, TUM trajectories, g2o graphs, Kümmerle relations, PGM + YAML maps and PNG
images, and the log readers by kind (docs/formats.md)."""
