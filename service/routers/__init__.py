"""The service's routes, one router per resource: health (page, probes, metrics), frames,
environment, stream."""
