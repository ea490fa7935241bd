"""What a person runs: `fabric-guidance` (cli: the table of subcommands, each imported when it
runs) and the subcommands that belong to no subject of their own (demo, example, replay,
recover). The subjects' commands live with their subject (experiments/, live_study/, bench/,
lab/)."""
