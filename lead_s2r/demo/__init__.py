"""The quickstart and the smoke twins' data: synthetic raw data -> adapters -> recipes -> tables, end to end."""
