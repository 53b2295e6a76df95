"""The station's web application (:func:`blackbox.station.web.app.create_app`)."""
