"""One module per CLI command (or family of commands); each exposes `register(app, bench)`."""
