"""The file formats, one module each, reader and writer, over one format-neutral log type
(:mod:`swarmslam.formats.records`: ``ScanLog``): CARMEN logs, ROS bags and MCAP, TUM trajectories, g2o graphs, Kümmerle relations, PGM + YAML maps and PNG
images, and the log readers by kind (docs/formats.md)."""
