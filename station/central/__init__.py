"""One central calibration history on PostgreSQL for a lab of stations (issue 16).

Each station keeps its SQLite store (station/store.py) as its offline, crash-safe journal and pushes its
ended sessions here with `station sync` (sync.py); the schema is the store's, by ordered migrations
(migrations.py); the panel reads it through `CentralStore` (reader.py). Arrays are files named by their
SHA-256 under the lab's array root, their paths in the database.
"""
