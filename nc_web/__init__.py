"""nc-web: the browser commissioning panel (issue 22); a client of the NC built on nc_link."""
