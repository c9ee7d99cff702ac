"""Pipeline stages: each reads its inputs, writes one artifact folder atomically with a manifest."""
