"""`fbcpr play`: a browser playground. session.py simulates and prompts the body, body.py draws its geoms, page.py
is the viser page and the 30 Hz loop."""
