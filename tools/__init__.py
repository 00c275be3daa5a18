"""The base station and `btf-host`.

`tools.cli` (the commands), `tools.station` (the process that owns the radio), `tools.page`
(the operator's page), `tools.store` (the SQLite database), `tools.analysis` (synthesis,
interpolation, metrics), `tools.data` (images, masks, datasets), `tools.report` (the HTML
report) and `tools.demo` (everything on fakes).
"""
