"""Labellers for the online labelling stage (see `pipeline.label`): one module each, exposing
`create(cfg: Config) -> Labeller`. `region_growing` is the classical online baseline; `mcpnet` the network."""
