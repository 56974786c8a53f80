"""Data from other tools in as factr2 recordings (MCAP): LeRobotDataset v3 folders (lerobot.py) and GELLO's
episode pickles (gello.py), both written through the one recorder (write.py), so every command that reads a
folder of recordings reads them. docs/bringing_data.md has each format's mapping and what is lost."""
