"""Images and datasets on disk: reading and writing images (`images`), label masks
(`masks`), historical BTF collections (`datasets`) and building a database from them
(`ingest`).
"""
