"""Request and response models: the OpenAPI contract of the dashboard."""
