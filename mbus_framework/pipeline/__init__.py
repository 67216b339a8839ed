"""The run pipeline, flowing one way: config -> components -> acquisition (written to disk
first) -> compensation -> estimation -> result.json -> report."""
