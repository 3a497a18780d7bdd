from roadlink.cli import app

app()
