"""Format-faithful raw-data generators; never import adapters (writer and reader share no code)."""
