"""Performance-driven animation from video (Chai, Xiao & Hodgins 2003)."""
