"""HTTP edge: routes, dependencies, error handlers, middleware. Only ``app.main`` imports it."""
