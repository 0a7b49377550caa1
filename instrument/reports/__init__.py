"""Inspection reports: what a plate's report holds (:mod:`.content`), the digest a reviewer
checks (:mod:`.digest`), and its HTML and PDF (:mod:`.render`, ``templates/``)."""
