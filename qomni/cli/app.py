"""The ``qomni`` typer application that every command module registers on."""
import typer

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Identification of the quasi-omnidirectional mobile platform (emulator, CANopen, "
                       "campaign, estimation).")
