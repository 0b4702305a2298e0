"""MERIS Level 1b products: ``n1`` (ENVISAT N1 files: FR/RR/FRS and AMORGOS FRG/FSG), ``sen3``
(4th-reprocessing ``.SEN3`` products) and ``open`` (``read_product``: either one)."""
