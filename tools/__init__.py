"""The base-station side: receive, store, synthesize, compare, report, demo."""
