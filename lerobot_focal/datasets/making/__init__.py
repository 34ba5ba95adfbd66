"""Making LeRobotDatasets: MetaWorld expert demos (`collect`, `lerobot-focal-collect`) with a crash-safe
episode-by-episode journal (`commit_log`), Adroit demos from Minari (`minari_import`,
`lerobot-focal-import-minari`), and small synthetic datasets for tests and demos (`synthetic`)."""
