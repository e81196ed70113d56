"""The pipelines: each a short module that composes the stages of
:mod:`monoavatar.pipelines.stages` into one capability (``reconstruct``: Paper B; ``animate``:
re-posing a finished avatar)."""
