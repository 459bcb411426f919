from faceanim.cli import run

run()
