"""Built-in adapters, installed as ``lead_s2r_adapters``; the core finds them through entry points."""
