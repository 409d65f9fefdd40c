"""Datasets, physics losses, trainers and the `drape train` command. Filled by the network issues."""
