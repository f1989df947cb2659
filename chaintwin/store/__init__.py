"""The results store (SQLite or PostgreSQL) and ingest of many recordings into it."""
