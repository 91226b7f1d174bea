"""rosbag2's sqlite3 storage (``.db3`` files), read in bulk (``reader``)."""

from twincd.io.sqlite3.reader import FETCH, Sqlite3Storage, SqliteDamage

__all__ = ["FETCH", "Sqlite3Storage", "SqliteDamage"]
