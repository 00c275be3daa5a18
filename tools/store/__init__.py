"""The base station's SQLite database: its schema and upgrades (`schema`), the records read
back (`rows`), and the store itself (`database`).
"""
