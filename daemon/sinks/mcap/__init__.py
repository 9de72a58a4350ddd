"""The MCAP log: the sink (``sink``) and the Foxglove messages it writes (``foxglove``)."""
