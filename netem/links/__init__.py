"""The link-model library: the models, their layered stack, the delivery matrix, closed forms."""
