"""Fuzzing gazehdr's parsers: `gazehdr fuzz` (see `runner`), the targets (`targets`), the
child process each runs in (`worker`) and the JSON-aware mutator (`jsonmut`). docs/fuzzing.md
has the campaign's figures."""
