"""HTTP edge: dependencies, routers, error mapping."""
