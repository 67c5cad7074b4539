"""CiA 402 drives outside the NC process, reached over zenoh (nc-drive-sim): see .drive and .host."""
