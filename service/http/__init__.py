"""The HTTP edge: the FastAPI app, its routes, request and response models, security
middleware, metrics and the static page.

May import `core` and the rest of `service`; renders only through `service.workers`."""
