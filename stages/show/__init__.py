"""Pictures a person checks, each drawing into an ``ax`` it is given (the figure and the PNG
are the caller's): one module per picture, with a ``main(conf, inputs..., output, *,
overwrite=False) -> Path`` that writes the PNG."""
