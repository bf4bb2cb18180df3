"""Rational polynomial (RPC) models: the terms (:mod:`.terms`), the model and its
evaluation (:mod:`.model`), reading and writing the vendors' formats (:mod:`.readers`,
:mod:`.writers`), fitting one to any sensor (:mod:`.fitting`) and the RPC sensor with its
corrections (:mod:`.sensor`)."""
