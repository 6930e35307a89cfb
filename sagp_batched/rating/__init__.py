"""Zone-rating backends: a local VLM, an OpenAI-compatible endpoint, and an offline prior."""
