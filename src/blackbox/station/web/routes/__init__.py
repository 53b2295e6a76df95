"""The station's pages, one router module per page group; ``web/app.py`` lists them."""
