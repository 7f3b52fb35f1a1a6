"""The `dotsim` program (cli: one subcommand per stage) and the commands that look at and ship data:
show (contact sheets, the IR overview, ground-truth PLY), view (the Rerun viewer), stats (the
dataset's statistics), export (WebDataset shards), pattern (make a dot pattern, its statistics),
dataset (verify, seal) and config (the built-in configs).

This folder sits above every stage: cli names the stages' own command modules (generator/cli.py,
trainer/cli.py, capture/cli.py, assets_manifest/cli.py) beside the ones here.
"""
