from roadlink.cli import main

main()
