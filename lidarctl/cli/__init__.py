"""The lidarctl command line: thin click commands over the library."""
