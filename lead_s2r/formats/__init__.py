"""Other projects' on-disk formats we read or write (pickles, protobuf descriptors, LEAD's sensor rigs).

No dataset logic lives here: adapters and writers build on these."""
