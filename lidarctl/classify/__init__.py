"""Classification into ASPRS classes: noise, ground, buildings, vegetation, water; fusion with the orthophoto."""
