"""The operator's page: served by the station (`server`), fed from the database (`data`), its
pictures drawn in worker processes (`drawing`), with command forms built from the command table
(`forms`) and its HTML, script and style in `static/`.
"""
