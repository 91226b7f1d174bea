"""Judge methods as the seed paper does: the method registry, the proposed method, the
baselines, metrics and reports."""
