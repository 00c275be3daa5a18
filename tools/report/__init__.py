"""The HTML report of a database (`document`), the look it shares with the operator's page
(`look`) and what a stored capture looks like (`capture_views`).
"""
