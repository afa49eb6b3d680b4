"""The link to a board: protocol codec and spec, ports, the session (heartbeat, reader), and sim://."""
