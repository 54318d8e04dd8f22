from qomni.cli import main

main()
