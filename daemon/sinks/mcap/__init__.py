"""The MCAP log: the sink (``sink``), its files (``recording``) and their retention (``retention``), the
camera images (``images``), and the Foxglove messages (``foxglove``) and schemas (``foxglove_schemas``)."""
