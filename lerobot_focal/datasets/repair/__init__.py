"""Repairing a LeRobotDataset whose writer was killed (`salvage`, `lerobot-focal-salvage-dataset`): the data files'
parquet footers are rebuilt (`parquet_footer`, over the minimal Thrift compact codec in `thrift_compact`)."""
