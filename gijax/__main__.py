from gijax.cli import run

run()
