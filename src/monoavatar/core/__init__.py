"""The base layer: what every stage shares and nothing of a stage. The camera
(:mod:`~monoavatar.core.camera`), landmark conventions (:mod:`~monoavatar.core.landmarks`),
the error hierarchy (:mod:`~monoavatar.core.errors`), atomic writes
(:mod:`~monoavatar.core.files`), thread pools (:mod:`~monoavatar.core.threads`), mesh
normals (:mod:`~monoavatar.core.geometry`) and the restricted unpickler
(:mod:`~monoavatar.core.safe_pickle`). It imports nothing else of monoavatar."""
